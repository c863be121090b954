"""The learned network: graph structures, encode–process–decode, normalizer, input noise."""
