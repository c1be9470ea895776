"""Where a study lives: SQLite under ``outputs/`` by default, PostgreSQL for many workers.

Credentials never go into configs: give the URL without a password (``postgresql://user@host/db``)
and the password in ``PGPASSWORD`` / ``~/.pgpass``, or put the whole URL in the environment
variable ``HYSTERESIS_LAB_OPTUNA_STORAGE``, which the sweeper reads and no file records.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import optuna
from sqlalchemy.engine import make_url
from sqlalchemy.exc import ArgumentError, IntegrityError

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
    """Connect, failing with a clear error (before any training) when the URL is unusable."""
    for attempt in range(5):
        try:
            return optuna.storages.RDBStorage(url, engine_kwargs=_engine_kwargs(url))
        except IntegrityError:  # another worker is creating the schema right now
            time.sleep(0.5 * (attempt + 1))
        except Exception as exc:  # SQLAlchemy / driver errors have many types
            raise _unusable(url, exc) from None
    return optuna.storages.RDBStorage(url, engine_kwargs=_engine_kwargs(url))


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
