"""Small shared utilities every layer may use: errors, atomic files and locks, paths, progress, memory limits,
checkpoint reading and the MLflow store. Imports nothing else of walkdiff."""
