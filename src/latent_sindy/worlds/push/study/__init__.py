"""The pushing world's study, ``latent-sindy reproduce`` (the paper's Table I and our
additions): scales, model catalogue, sweeps, stages and jobs, tables, figures and report.
The generic pieces it builds on (study folder, evaluation, HTML report) are in
:mod:`latent_sindy.study`."""
