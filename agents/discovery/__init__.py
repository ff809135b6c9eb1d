"""Strategy discovery (thesis §3.5, §3.7): the real black box, the gallery, Stage 2, run-ups."""
