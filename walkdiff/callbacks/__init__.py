"""Training plumbing: the LightningCLI runner behind `walkdiff fit`, the callbacks a config names
(checkpoints, metrics, sample previews, MLflow run records). Tasks never import it; it imports the tasks it
previews."""
