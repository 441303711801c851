"""Control side: robot description, dynamic models and the lead-through controller."""
