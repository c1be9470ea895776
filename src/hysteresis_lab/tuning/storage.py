"""Where a study lives: SQLite under ``outputs/`` by default, PostgreSQL for many workers.

Credentials never go into configs: give the URL without a password (``postgresql://user@host/db``)
and the password in ``PGPASSWORD`` / ``~/.pgpass``, or put the whole URL in the environment
variable ``HYSTERESIS_LAB_OPTUNA_STORAGE``, which the sweeper reads and no file records.
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import optuna
from sqlalchemy import create_engine, text
from sqlalchemy.engine import make_url
from sqlalchemy.exc import ArgumentError, DBAPIError, IntegrityError

from hysteresis_lab.errors import ConfigError

STORAGE_ENV = "HYSTERESIS_LAB_OPTUNA_STORAGE"


def resolve_storage_url(configured: str | None, study_name: str, results_dir: Path) -> str:
    """The storage URL: the environment variable, else the configured URL, else SQLite."""
    url = os.environ.get(STORAGE_ENV) or configured
    if not url:
        results_dir.mkdir(parents=True, exist_ok=True)
        return f"sqlite:///{(results_dir / f'{study_name}.db').as_posix()}"
    if configured and not os.environ.get(STORAGE_ENV) and _has_password(configured):
        raise ConfigError(
            "hydra.sweeper.storage contains a password, which Hydra would save in every "
            f"run's config. Fix: export {STORAGE_ENV}='<url with password>' instead, or give "
            "the URL without a password and the password in PGPASSWORD or ~/.pgpass."
        )
    return url


def redact(url: str) -> str:
    """The URL with any password masked, for logs."""
    try:
        return make_url(url).render_as_string(hide_password=True)
    except ArgumentError:
        return "<unparseable storage URL>"


def _has_password(url: str) -> bool:
    try:
        return make_url(url).password is not None
    except ArgumentError:
        return False


def open_storage(url: str) -> optuna.storages.BaseStorage:
    """Connect, failing with a clear error (before any training) when the URL is unusable.

    Workers started together on a fresh database all try to create Optuna's schema: on
    PostgreSQL they take turns under an advisory lock; on any backend, a worker that loses the
    race (the table or type "already exists") retries, and then finds the schema made.
    """
    last: Exception | None = None
    for attempt in range(_SCHEMA_RACE_RETRIES):
        try:
            with _schema_lock(url):
                return optuna.storages.RDBStorage(url, engine_kwargs=_engine_kwargs(url))
        except Exception as exc:  # SQLAlchemy / driver errors have many types
            if not _lost_schema_race(exc):
                raise _unusable(url, exc) from None
            last = exc
            time.sleep(0.2 * (attempt + 1))
    raise _unusable(url, last) from None


_SCHEMA_RACE_RETRIES = 8
# SQLSTATEs of "someone else created it first": unique_violation, duplicate_table,
# duplicate_object.
_ALREADY_EXISTS = {"23505", "42P07", "42710"}


def _lost_schema_race(exc: Exception) -> bool:
    if isinstance(exc, IntegrityError):
        return True
    if not isinstance(exc, DBAPIError):
        return False
    state = getattr(exc.orig, "sqlstate", None) or getattr(exc.orig, "pgcode", None)
    return state in _ALREADY_EXISTS or "already exists" in str(exc.orig)


@contextmanager
def _schema_lock(url: str) -> Iterator[None]:
    """On PostgreSQL, hold a session advisory lock while the schema is checked and created."""
    if not url.startswith("postgresql"):
        yield
        return
    engine = create_engine(url, **_engine_kwargs(url))
    try:
        with engine.connect() as connection:
            connection.execute(text("SELECT pg_advisory_lock(:key)"), {"key": _LOCK_KEY})
            try:
                yield
            finally:
                connection.execute(text("SELECT pg_advisory_unlock(:key)"), {"key": _LOCK_KEY})
    finally:
        engine.dispose()


_LOCK_KEY = 0x68797374  # any fixed 64-bit number; "hyst"


def _unusable(url: str, exc: Exception) -> ConfigError:
    return ConfigError(
        f"cannot open the Optuna storage {redact(url)}: {type(exc).__name__}: "
        f"{str(exc).splitlines()[0] if str(exc) else ''}. Fix: check the URL, that the "
        "database server is running and reachable, and that its driver is installed "
        "(psycopg[binary] for PostgreSQL: pip install hysteresis-lab[distributed])."
    )


def _engine_kwargs(url: str) -> dict:
    if url.startswith("sqlite"):
        return {"connect_args": {"timeout": 60}}
    if url.startswith("postgresql"):
        return {"pool_pre_ping": True, "connect_args": {"connect_timeout": 10}}
    return {}
