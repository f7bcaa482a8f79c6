"""The exit statuses of the ``ddvi`` commands that are not a run's (a run's, with its status 3
for a completed mission that degraded: ``services.ground.launch.lifecycle``)."""

EXIT_OK, EXIT_FAIL, EXIT_USAGE = 0, 1, 2
"""Done; failed (a learner that did not converge, a report that could not be written); a usage
or input error, said in one line."""
