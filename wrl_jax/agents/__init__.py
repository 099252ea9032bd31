"""Hand-written RL algorithms (PPO, DQN) and the contract the training driver uses."""
