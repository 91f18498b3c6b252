"""Offline analysis of run logs: tidy pandas frames, the paper's tables, plots."""
