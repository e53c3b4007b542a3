"""Persistence shared by the API and the workers: the SQLite catalog (:mod:`persist.catalog`) and the
content-addressed artifact store (:mod:`persist.store`).

Imports ``proto`` only (contracts); ``proto`` never imports this package. Holds no math and no HTTP.
"""
