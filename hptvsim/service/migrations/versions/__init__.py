"""The revisions: ``0001`` is the 0.1.0 schema, every later one upgrades its predecessor."""
