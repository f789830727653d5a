"""What every algorithm's training shares: the simulated worlds (in process or in worker processes), the multi-agent
modes' streams, n-step windows, observation scaling and the learning curve."""
