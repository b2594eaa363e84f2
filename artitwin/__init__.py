"""The ArtiTwin application: the ``artitwin`` command line (top layer, above flows)."""
