"""The learned network: graph structures, encode–process–decode, normaliser, input noise."""
