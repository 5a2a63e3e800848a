"""NSRR's training (clss/methods/nsrr/): the torch twin of its frame step (twin.py) and the
recipe (recipe.py)."""
