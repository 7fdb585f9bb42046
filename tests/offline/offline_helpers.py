"""Constants shared by the offline tests (imported as ``offline_helpers`` from this folder)."""

TINY_STEPS = 60  # steps per episode of the tiny dataset: windows longer than K, seconds to collect
