"""Bearer tokens and roles (CONTRACT section 2): ``unit`` posts scans, ``reader`` reads,
``admin`` does both. With no tokens configured the server is open (and loopback-only,
which the settings enforce)."""

from __future__ import annotations

import hmac
from collections.abc import Callable

from fastapi import HTTPException, Request

from mapserver.settings import Role, Settings

WRITE = "write"
READ = "read"
ALLOWED = {WRITE: {Role.UNIT, Role.ADMIN}, READ: {Role.READER, Role.ADMIN}}


def require(action: str) -> Callable[[Request], None]:
    """A FastAPI dependency that admits a request allowed to ``action`` (WRITE or READ)."""

    def check(request: Request) -> None:
        settings: Settings = request.app.state.settings
        if settings.open_access:
            return
        header = request.headers.get("authorization", "")
        scheme, _, token = header.partition(" ")
        if scheme.lower() != "bearer" or not token:
            raise HTTPException(
                401,
                "authorization: a bearer token is required (Authorization: Bearer TOKEN)",
                headers={"WWW-Authenticate": "Bearer"},
            )
        role = _role_of(token.strip(), request.app.state.token_roles)
        if role is None:
            raise HTTPException(
                401, "authorization: the bearer token is not valid", {"WWW-Authenticate": "Bearer"}
            )
        if role not in ALLOWED[action]:
            raise HTTPException(403, f"authorization: role {role.value!r} may not {action}")

    return check


def _role_of(token: str, roles: dict[str, Role]) -> Role | None:
    """The role of ``token``, compared in constant time against every configured token."""
    found = None
    for secret, role in roles.items():
        if hmac.compare_digest(secret.encode(), token.encode()):
            found = role
    return found
