"""UAV camera geometry, renderers, UGV detector, feature vector φ(s) and Zenoh frame transport."""
