"""CLSS's training (clss/methods/clss/): the torch twin of the frame step (twin.py), the
two-stage recipe (recipe.py), and two studies of its history decision: `python -m
weights_tools classifier` (classifier_report.py) and the visibility oracle
(visibility_oracle.py)."""
COMMANDS = {"classifier": "classifier_report"}
