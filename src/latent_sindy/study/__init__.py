"""What any world's study uses, knowing no world: the settings every study takes
(:mod:`.settings`), the study folder and the run of a world plug-in's study through its
``reproduce`` hook, the one entry of every world's study (:mod:`.runner`), the measurements
of a trained run on the same footing as every other (:mod:`.evaluation`), the
self-contained HTML report (:mod:`.report`), and the model-based study of any world with a
reward, SINDy, linear and MLP latents each through PlaNet's loop (:mod:`.model_based`, its
report :mod:`.model_based_report`). A world's study (``latent_sindy.worlds.<world>``) builds
on these."""
