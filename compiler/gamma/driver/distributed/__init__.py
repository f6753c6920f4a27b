"""Ray: ``cluster`` connects to it (the optional extra), ``distributed``
traces a run's iterations on its workers (``gammac run --ray``), and
``sweep`` runs a parameter grid as its tasks (``gammac sweep``).
"""
