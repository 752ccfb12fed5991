"""Bearer tokens and roles (docs/http-api.md): ``unit`` posts scans and unit states as
the units its token lists, ``reader`` reads, ``admin`` does both, as any unit. With no
tokens configured the server is open (and loopback-only, which the settings and
``local_only`` enforce)."""

from __future__ import annotations

import hmac
from collections.abc import Callable

from fastapi import HTTPException, Request

from mapserver.service.settings import Role, Settings, TokenSettings

WRITE = "write"
READ = "read"
ALLOWED = {WRITE: {Role.UNIT, Role.ADMIN}, READ: {Role.READER, Role.ADMIN}}


def require(action: str) -> Callable[[Request], None]:
    """A FastAPI dependency that admits a request allowed to ``action`` (WRITE or READ);
    the admitted token's settings are left in ``request.state.token`` (None when open)."""

    async def check(request: Request) -> None:  # async: no worker-thread hop per request
        settings: Settings = request.app.state.settings
        request.state.token = None
        if settings.open_access:
            return
        header = request.headers.get("authorization", "")
        scheme, _, secret = header.partition(" ")
        if scheme.lower() != "bearer" or not secret:
            raise HTTPException(
                401,
                "authorization: a bearer token is required (Authorization: Bearer TOKEN)",
                headers={"WWW-Authenticate": "Bearer"},
            )
        token = _token_of(secret.strip(), request.app.state.tokens)
        if token is None:
            raise HTTPException(
                401, "authorization: the bearer token is not valid", {"WWW-Authenticate": "Bearer"}
            )
        if token.role not in ALLOWED[action]:
            raise HTTPException(
                403,
                f"authorization: token {token.name!r} of role {token.role.value!r} "
                f"may not {action}",
            )
        request.state.token = token

    return check


def require_unit(request: Request, unit_id: str, field: str) -> None:
    """403 unless the request's token may post as ``unit_id`` (``field`` names where the
    id was in the body). Call after ``require(WRITE)`` admitted the request."""
    token: TokenSettings | None = request.state.token
    if token is None or token.may_post_as(unit_id):
        return
    raise HTTPException(
        403,
        f"{field}: token {token.name!r} may not post as unit {unit_id!r} "
        f"(it may post as {', '.join(token.units or ())})",
    )


def _token_of(secret: str, tokens: dict[str, TokenSettings]) -> TokenSettings | None:
    """The token whose secret is ``secret``, compared in constant time against each."""
    found = None
    for candidate, token in tokens.items():
        if hmac.compare_digest(candidate.encode(), secret.encode()):
            found = token
    return found
