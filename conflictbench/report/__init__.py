"""Reports over the episode store: tables in the terminal and as files."""

from .summary import report_records, summary_frame

__all__ = ["report_records", "summary_frame"]
