"""Learning algorithms on stable-baselines3: prioritized replay, dueling DQN, multi-agent modes, callbacks."""
