"""fignetctl: photographs to a simulated, re-rendered what-if video with FIGNet*."""

__version__ = "0.1.0"
