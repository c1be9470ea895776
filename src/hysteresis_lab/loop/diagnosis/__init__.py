"""The loop's residual analysis: which effect a model lacks, from arrays alone.

`ranking` scores the candidate effects on the held-out residual (its held-out fits from
`normal_equations`); `residuals` (with `correlation` and `spectrum`) gives one model's
residual tests and figures; `excitation` compares how hard recordings drive an effect's
operators.
"""
