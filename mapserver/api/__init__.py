"""The map server's HTTP edge (FastAPI): a thin layer over ``mapserver.service.map_service``."""
