"""Neural fields: hash-grid encoding and the radiance field built on it."""
