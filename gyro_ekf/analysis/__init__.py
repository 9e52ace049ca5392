"""Offline analysis: the offline pipeline, metrics, summaries and figures of filter runs."""
