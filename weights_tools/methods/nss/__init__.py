"""NSS's training room: the torch twin (twin.py) and the recipe (recipe.py)."""
