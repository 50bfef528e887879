"""Walkers steered live by people and programs: `walkdiff control` (JSON lines), `walkdiff play --script`
(timed key events replayed into a take) and the page of `walkdiff play` (keys in a browser)."""
