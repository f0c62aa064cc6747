"""The application layer: the ``qpik`` command, scenario runs, figures and the peer
libraries. Nothing in the core or in ``qpik.robots`` imports it."""
