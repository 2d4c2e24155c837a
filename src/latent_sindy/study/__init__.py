"""What any world's study uses, knowing no world: the study folder and the run of a world
plug-in's own study (:mod:`.runner`), the measurements of a trained run on the same footing
as every other (:mod:`.evaluation`) and the self-contained HTML report (:mod:`.report`).
A world's study (``latent_sindy.worlds.<world>``) builds on these."""
