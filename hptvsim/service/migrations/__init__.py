"""Alembic migrations of the service database (run by :class:`hptvsim.service.db.Store` on startup).

``env.py`` is the Alembic environment; ``versions/`` holds one file per schema revision, named
``rev_<number>_<what>.py`` (valid module names, so the type checker and linter can read them).
A new revision: ``alembic -c <an ini naming script_location = hptvsim/service/migrations>
revision -m "..."``, rename the file after that pattern, and give it the next number as its
``revision``.
"""
