"""Measuring code: the accuracy-against-time sweeps (`tradeoff`), the paper's Table 1 on our
data (`memory`, for bench-memory) and the statistics they share (`stats`). It measures the
library; nothing under fignetctl/core imports it."""
