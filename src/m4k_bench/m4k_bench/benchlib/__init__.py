"""Building blocks of ``bench`` (the paper's evidence in one run).

* :mod:`.analysis` -- pure: timing CSVs -> per-condition statistics, the summary's ratios and
  the targets (target, measured, met or not, why);
* :mod:`.report` -- pure: summary dict -> ``report.md``;
* :mod:`.plots` -- the Fig. 10 periodicity plots (matplotlib, Agg);
* :mod:`.cyclic` -- cyclictest command line and output parsing;
* :mod:`.system` -- tool set-up (rt-tests, stress-ng), machine description, stress-ng runs,
  process CPU time;
* :mod:`.stack` -- starting and stopping rt_core / driver_host / baseline / bridge, feeding
  commands and recording the status port;
* :mod:`.cmdlat` -- cmd_vel -> WHEEL_CMD latency through the ROS bridge and a probe peer;
* :mod:`.progress` -- one updating line on a TTY, plain lines otherwise.
"""
