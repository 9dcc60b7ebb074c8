"""Self-contained HTML reports: tables and matplotlib figures embedded as data URIs."""

from rwlab.report.html import Page, figure

__all__ = ["Page", "figure"]
