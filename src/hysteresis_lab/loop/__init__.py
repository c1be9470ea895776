"""The closed loop (``hysteresis-lab-loop``): fit -> residuals -> diagnose -> add -> refit.

* `driver`: the rounds, their decisions and ``loop_report.json`` (`run_loop`);
* `data`: which recordings train, validate, choose the effect and report;
* `diagnosis`: pure analysis of a round's residual (the effect ranking, residual tests and
  spectrum, operator excitation); it reads arrays and runs nothing;
* `advice`: what to record where an effect cannot be judged for lack of excitation;
* `report` and `figures`: ``loop_report.md`` and the figures it links;
* `checks`: a finished run against what only a simulator knows (reads its folder).
"""
