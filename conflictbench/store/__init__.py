"""The episode store (public schema in ``conflictbench.store.schema`` and the README)."""

from .episodes import EpisodeStore
from .schema import SCHEMA, SCHEMA_VERSION, records_to_table, table_to_records

__all__ = ["EpisodeStore", "SCHEMA", "SCHEMA_VERSION", "records_to_table", "table_to_records"]
