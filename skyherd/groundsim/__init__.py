"""Ground vehicles: UGV model, scripted behaviours, a numpy unicycle world and a PyBullet world."""
