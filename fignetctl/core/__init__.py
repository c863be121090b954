"""The library: arrays in, arrays out; no argument parsing."""
