"""Studies: every policy x initializer x motion on the same seeds, and what is written about them.

``evaluate.py`` is the command line; this package is the library behind it, one job per module:

- :mod:`~aasl_gym.study.jobs`: the grid of episodes (:class:`~aasl_gym.study.jobs.Job`) and each one's key;
- :mod:`~aasl_gym.study.runner`: many episodes in this process, on a process pool or as Ray tasks (what
  runs one is given: :func:`agents.study.run_episode` flies the agents, which this package does not import);
- :mod:`~aasl_gym.study.log`: ``episodes.jsonl``, the log a study resumes from;
- :mod:`~aasl_gym.study.stats`: summaries with confidence intervals, paired comparisons;
- :mod:`~aasl_gym.study.report`: ``report.md``, ``results.json`` and the console table;
- :mod:`~aasl_gym.study.plots`: convergence, success and trajectory figures.
"""
