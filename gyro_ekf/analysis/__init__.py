"""Offline analysis: metrics, summaries, outputs and figures of filter runs."""
