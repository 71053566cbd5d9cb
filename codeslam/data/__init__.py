"""Datasets: the typed :class:`Frame` record and one reader per format (see ``registry.py``); camera trajectories
and their files (``trajectory.py``: TUM, ``euroc_csv.py``, ``trajectory_file.py``) and timestamp association
(``association.py``)."""
