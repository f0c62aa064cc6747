"""``qpik sweep``: a Monte-Carlo study over a bundled robot's workspace, as chunks of
batched worlds (:mod:`qpik.batch`), in-process or on a Ray cluster, resumable.

- :mod:`.studies`: what is sampled (targets, start states, gains) and which batched
  controllers run, per robot;
- :mod:`.rollout`: one chunk's rollout and its per-world metrics;
- :mod:`.chunks`: chunk keys, files written whole, what is finished;
- :mod:`.runners`: in-process, or Ray tasks;
- :mod:`.report` and :mod:`.figures`: summary.json, the table, the workspace maps;
- :mod:`.command`: the command line.

docs/sweep.md describes the study, the files and how it would run on many nodes.
"""
