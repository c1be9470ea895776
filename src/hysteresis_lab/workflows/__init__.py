"""The orchestrators: they train, score and write run folders, built on the pure parts
(`hysteresis_lab.fitting`, `hysteresis_lab.evaluation`).

* `pipeline`: train and evaluate one model (``hysteresis-lab-train``, `hysteresis_lab.api`);
* `paper`: the study's four models, trained in parallel, and its Table 2;
* `grow`: a declared physical model grown stage by stage, as the loop grows one.

The closed loop (``hysteresis-lab-loop``) is its own package, `hysteresis_lab.loop`.
"""
