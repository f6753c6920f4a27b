"""What a run leaves: the writers on the run's events (``writers``: maps,
renders, summary, sequence, export; ``progress``: the bar), the encoders
(``outputs``: PLY, false-colour PNG, JSON), the texture set and glTF/OBJ
(``export``, with ``atlas`` for meshes without UVs), OpenUSD
(``usd_export``), and ``saved``: renders and exports of a saved run.
"""
