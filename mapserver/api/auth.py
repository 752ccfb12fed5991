"""Bearer tokens and roles (docs/http-api.md): ``unit`` posts scans and unit states as
the units its token lists, ``reader`` reads, ``admin`` does both, as any unit. With no
tokens configured the server is open (and loopback-only, which the settings and
``local_only`` enforce)."""

from __future__ import annotations

import hmac
from collections.abc import Callable
from typing import Any

from fastapi import HTTPException, Request, Security
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from mapserver.core.text import quote
from mapserver.service.settings import Role, Settings, TokenSettings

WRITE = "write"
READ = "read"
DECLARE_CLOCK = "declare the clock"
ALLOWED = {
    WRITE: {Role.UNIT, Role.ADMIN},
    READ: {Role.READER, Role.ADMIN},
    DECLARE_CLOCK: {Role.ADMIN},
}
BEARER_SCHEME = "bearerAuth"
"""The OpenAPI security scheme's name (``openapi_security``)."""
BEARER = HTTPBearer(
    auto_error=False,  # ``require`` answers a missing or wrong token itself
    scheme_name=BEARER_SCHEME,
    description="A token from the server's `tokens` setting (or FLEETMAP_TOKENS); roles: "
    "`unit` posts, `reader` reads, `admin` both. An open server (no tokens, loopback "
    "only) needs none.",
)
WHO = {
    WRITE: "a `unit` token (posting only as the units it lists) or an `admin` token",
    READ: "a `reader` or an `admin` token",
    DECLARE_CLOCK: "only an `admin` token",
}


def require(action: str) -> Callable[[Request], None]:
    """A FastAPI dependency that admits a request allowed to ``action`` (WRITE or READ);
    the admitted token's settings are left in ``request.state.token`` (None when open)."""

    async def check(  # async: no worker-thread hop per request
        request: Request,
        # FastAPI's marker, read once at definition: it declares the scheme in the
        # OpenAPI schema (openapi_security); the header is checked below.
        _bearer: HTTPAuthorizationCredentials | None = Security(BEARER, scopes=[action]),  # noqa: B008
    ) -> None:
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


def openapi_security(schema: dict[str, Any]) -> None:
    """Finish the bearer scheme in an OpenAPI ``schema``: FastAPI lists it on every
    operation whose ``require`` check declares it, with the action as a marker scope;
    the marker becomes an empty list (bearer tokens have no scopes) and the roles it
    admits a sentence of the operation's description."""
    for path in schema.get("paths", {}).values():
        for operation in path.values():
            requirements = operation.get("security") or []
            actions = [a for r in requirements for a in r.get(BEARER_SCHEME, ()) if a in WHO]
            if not actions:
                continue
            operation["security"] = [{BEARER_SCHEME: []}]
            note = (
                f"Token: {WHO[actions[0]]} (`Authorization: Bearer TOKEN`) when the server "
                "has tokens; 401 without a valid one, 403 for a token of another role. An "
                "open server needs none."
            )
            described = operation.get("description", "")
            operation["description"] = f"{described}\n\n{note}" if described else note


def require_unit(request: Request, unit_id: str, field: str) -> None:
    """403 unless the request's token may post as ``unit_id`` (``field`` names where the
    id was in the body). Call after ``require(WRITE)`` admitted the request."""
    token: TokenSettings | None = request.state.token
    if token is None or token.may_post_as(unit_id):
        return
    raise HTTPException(
        403,
        f"{field}: token {token.name!r} may not post as unit {quote(unit_id)} "
        f"(it may post as {', '.join(token.units or ())})",
    )


def _token_of(secret: str, tokens: dict[str, TokenSettings]) -> TokenSettings | None:
    """The token whose secret is ``secret``, compared in constant time against each."""
    found = None
    for candidate, token in tokens.items():
        if hmac.compare_digest(candidate.encode(), secret.encode()):
            found = token
    return found
