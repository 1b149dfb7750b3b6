"""Reporting: metrics rows, safety metrics and intervals, the end-of-run summary, compare, plots and video."""
