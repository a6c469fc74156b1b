"""One active-mapping episode: its resolved settings, the step loop (Algorithm 1), the per-step images,
and the runner that records and resumes it."""
