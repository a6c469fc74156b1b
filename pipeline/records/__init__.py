"""Run records: run.json, steps.jsonl and the DONE / FAILED markers of one run directory."""
