"""Benchmarks: programs that print figures, the last line name=value (console scripts automotive-bench-*)."""
