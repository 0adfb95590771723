"""The command line: thin wrappers around the API, and the runs of project files end to end
that write reports (one project: `_adjust`; a batch: `run_batch`, public as `jaxba.run_batch`)."""
