"""The shader MLP upscaler's training (clss/methods/mlp/): the torch twin of its frame step
(twin.py), the offline recipe (recipe.py), and the online learning curve on the device
(online.py: `python -m weights_tools.methods.mlp.online`)."""
