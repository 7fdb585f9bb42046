"""Trained policies out of Python: ONNX files and the runtime that runs them.

* :mod:`hptvsim.export.runtime`: loads ``DIR/<agent>.onnx`` and acts, with numpy and onnxruntime
  only (no torch, no stable-baselines3, no other part of hptvsim): what a companion computer runs;
* :mod:`hptvsim.export.build`: ``hptvsim policy export SPEC --out DIR``, each file checked
  against the SB3 model it came from;
* :mod:`hptvsim.export.dt`: a Decision Transformer's graph, its context as inputs, checked
  against :class:`~hptvsim.offline.policy.DTPolicy`;
* :mod:`hptvsim.export.cli`: the ``hptvsim policy`` commands.

This package imports nothing at import time, so ``hptvsim.export.runtime`` stays light.
"""
