"""Schemathesis against the app's own OpenAPI schema, in-process: no 5xx, no reply that
breaks its own schema, whatever the generated input (every operation in turn).

The check that schema-valid input is accepted is left out: a schema cannot say that the
sensor must be on the map or that a unit's stamps never go backwards, and refusing such
scans with a 4xx is the contract."""

import tempfile

import pytest
import schemathesis
from hypothesis import HealthCheck, given, settings
from server_helpers import small_settings

from mapserver.api.app import create_app

CHECKS = [
    schemathesis.checks.not_a_server_error,
    schemathesis.checks.status_code_conformance,
    schemathesis.checks.content_type_conformance,
    schemathesis.checks.response_schema_conformance,
    schemathesis.checks.response_headers_conformance,
]


@pytest.fixture(scope="module")
def api_schema():
    with tempfile.TemporaryDirectory() as data_dir:
        app = create_app(small_settings(data_dir))
        yield schemathesis.openapi.from_asgi("/openapi.json", app)
        app.state.service.close()


def test_every_operation_never_fails_and_keeps_its_own_schema(api_schema):
    operations = [result.ok() for result in api_schema.get_all_operations()]
    assert {op.path for op in operations} >= {"/v1/scans", "/v1/costmap", "/v1/query/cells"}
    for operation in operations:

        @given(case=operation.as_strategy())
        @settings(max_examples=30, deadline=None, suppress_health_check=list(HealthCheck))
        def check(case):
            case.call_and_validate(checks=CHECKS)

        check()
