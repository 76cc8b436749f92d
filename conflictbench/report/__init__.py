"""Reports over the episode store: the paper's tables (terminal, Markdown, LaTeX, CSV) and figures."""

from .summary import report_records, select_metrics
from .tables import DIRECTIONS, paper_tables

__all__ = ["DIRECTIONS", "paper_tables", "report_records", "select_metrics"]
