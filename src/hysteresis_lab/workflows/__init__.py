"""The orchestrators: they train, score and write run folders, built on the pure parts
(`hysteresis_lab.fitting`, `hysteresis_lab.evaluation`, `hysteresis_lab.analysis`).

* `pipeline`: train and evaluate one model (``hysteresis-lab-train``, `hysteresis_lab.api`);
* `paper`: the study's four models, trained in parallel, and its Table 2;
* `loop`: the closed loop's driver (``hysteresis-lab-loop``), with `loop_data` choosing which
  recordings train, choose the effect and judge it.
"""
