"""Small examples of the package's extension points (a user's own task)."""
