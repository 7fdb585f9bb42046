"""Offline RL: expert datasets in Minari format and the Decision Transformer (paper section IV-D).

The last stage of ETFDU (paper Algorithm 1, lines 19-23): expert trajectories become offline
datasets (:mod:`hptvsim.offline.dataset`, ``hptvsim collect``); Decision Transformers
(:mod:`hptvsim.offline.model`) are trained on them (:mod:`hptvsim.offline.trainer`,
``hptvsim dt train``), drive the pursuers as ordinary policies (:mod:`hptvsim.offline.policy`,
zoo kind ``dt``) and are evaluated in the full game (:mod:`hptvsim.offline.evaluate`,
``hptvsim dt evaluate``), with the paper's figures (:mod:`hptvsim.offline.figures`). The whole
stage is one command: ``hptvsim dt pipeline`` (:mod:`hptvsim.offline.pipeline`).

Heavy modules (torch, minari) load only when used.
"""
