"""The local-model protocol: codes, the wire table, update and proxy-state codecs."""
