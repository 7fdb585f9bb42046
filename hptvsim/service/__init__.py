"""The hptvsim digital-twin service (FastAPI): the top layer.

It imports the library below it; nothing in the library imports it (only the CLI,
:mod:`hptvsim.cli`, starts it: ``hptvsim serve``).
"""
