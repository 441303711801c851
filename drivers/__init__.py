"""Device drivers: one process per fieldbus, bridging it to the zenoh bus."""
