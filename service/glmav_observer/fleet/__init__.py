"""Fleet scale: ``serve --workers N`` (one machine, all cores) and ``serve --claim``
(several services splitting a fleet through Zenoh claims). See docs/deployment.md."""
