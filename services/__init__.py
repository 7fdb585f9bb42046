"""The hptvsim digital-twin service (FastAPI). It imports hptvsim; hptvsim never imports it."""
