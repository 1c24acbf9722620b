"""PhyIR networks: GMNet, LNet, GSNet."""
