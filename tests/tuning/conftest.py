"""Fixtures of the sweep tests (helpers live in sweep_helpers.py)."""

from __future__ import annotations

import pytest
from sweep_helpers import PG_URL_DEFAULT, postgres_url


@pytest.fixture(scope="session")
def pg_url() -> str:
    url = postgres_url()
    if url is None:
        pytest.skip("no PostgreSQL server at ASLEXP_TEST_POSTGRES_URL (default "
                    f"{PG_URL_DEFAULT}); start one with: bash scripts/ci_postgres.sh")
    return url
