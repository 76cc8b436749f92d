"""Reports over the episode store: the paper's tables (terminal, Markdown, LaTeX, CSV) and figures."""

from .from_store import report_store
from .summary import report_records, select_metrics
from .tables import OUTCOME_DIRECTIONS, paper_tables

__all__ = ["OUTCOME_DIRECTIONS", "paper_tables", "report_records", "report_store", "select_metrics"]
