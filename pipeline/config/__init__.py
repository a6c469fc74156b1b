"""A run's configuration: the Hydra schema, validation before any work, and the settings a record holds
beyond its named groups."""
