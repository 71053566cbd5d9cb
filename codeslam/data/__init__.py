"""Datasets: the typed :class:`Frame` record and one reader per format (see ``registry.py``)."""
