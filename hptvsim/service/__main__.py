"""``python -m hptvsim.service``: the same as ``hptvsim serve``."""

from hptvsim.service.cli import serve

if __name__ == "__main__":
    serve(prog_name="hptvsim serve")
