"""NSRD's training (clss/methods/nsrd/): the torch twin of its frame step (twin.py) and the
recipe (recipe.py)."""
