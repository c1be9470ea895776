"""The closed loop (``hysteresis-lab-loop``): fit -> residuals -> diagnose -> add -> refit."""
