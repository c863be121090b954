"""Measuring code: the accuracy-against-time sweeps (`tradeoff`), the paper's Table 1 on our
data (`memory`, for bench-memory), the statistics they share (`stats`) and the options of the
scripts in benchmarks/ (`options`). It measures the library; nothing under fignetctl/core
imports it."""
