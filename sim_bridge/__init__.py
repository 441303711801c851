"""Virtual robot cell: plant, vendor controller, I/O and their fieldbus endpoints."""
