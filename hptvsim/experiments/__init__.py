"""Experiments: what starts from policy names, or needs training and offline RL together.

Above the policy zoo (:mod:`hptvsim.zoo`), which sits above training and offline RL:

* :mod:`hptvsim.experiments.policies`: policy specs with the zoo's names (``hptvsim train``'s
  fixed policies, ``hptvsim evaluate``);
* :mod:`hptvsim.experiments.collect`: expert datasets from named policies (``hptvsim collect``);
* :mod:`hptvsim.experiments.dt_evaluate`: the Decision Transformer against named experts
  (``hptvsim dt evaluate``);
* :mod:`hptvsim.experiments.dt_pipeline`: the whole offline-RL stage and its figures
  (``hptvsim dt pipeline | figures``);
* :mod:`hptvsim.experiments.sweeps`: settings x seeds on Ray (``hptvsim sweep``);
* :mod:`hptvsim.experiments.figures`, :mod:`hptvsim.experiments.stats`,
  :mod:`hptvsim.experiments.reproduce`: the paper's figures and the reproduction of section V
  with intervals over seeds (``hptvsim figures``, ``hptvsim reproduce``), whose DT steps (the
  offline stage on the reproduction's own experts, over seeds) are
  :mod:`hptvsim.experiments.repro_dt`;
* :mod:`hptvsim.experiments.cli`: their commands.

Nothing below imports this package; it imports nothing above the zoo and the catalog.
"""
