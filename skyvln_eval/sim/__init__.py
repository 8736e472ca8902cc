"""Simulation: view rendering, quadrotor plant, obstacle scenarios."""
