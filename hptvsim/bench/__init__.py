"""Benchmarks (``hptvsim bench ...``): costs as ratios to a floor or a peer in the same run."""
