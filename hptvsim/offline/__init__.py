"""Offline RL: expert datasets in Minari format and the Decision Transformer (paper section IV-D).

The last stage of ETFDU (paper Algorithm 1, lines 19-23): expert trajectories become offline
datasets (:mod:`hptvsim.offline.dataset`); Decision Transformers
(:mod:`hptvsim.offline.model`) are trained on them (:mod:`hptvsim.offline.trainer`,
``hptvsim dt train``) and drive the pursuers as ordinary policies (:mod:`hptvsim.offline.policy`,
zoo kind ``dt``), with the paper's figures (:mod:`hptvsim.offline.figures`).

What starts from policy names sits above the policy zoo, in :mod:`hptvsim.experiments`:
collecting the experts' datasets (:mod:`hptvsim.experiments.collect`, ``hptvsim collect``),
evaluating DTs against the experts (:mod:`hptvsim.experiments.dt_evaluate`,
``hptvsim dt evaluate``) and the whole stage in one command (``hptvsim dt pipeline``,
:mod:`hptvsim.experiments.dt_pipeline`). This package never imports :mod:`hptvsim.train`.

Heavy modules (torch, minari) load only when used.
"""
