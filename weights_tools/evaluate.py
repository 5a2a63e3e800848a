"""`python -m weights_tools eval`: the evaluation of clss.evaluate (the one scoring code,
shared with `clss eval`), re-exported here for the training tools (`seeds` scores the
torch twins through evaluate_sequence(run=...))."""
from clss.evaluate import (METHODS, UNTRAINED, Pipeline, SequenceError, add_arguments,  # noqa: F401
                           canonical_methods, evaluate_sequence, format_table, load_sequence,
                           main_args, make_method, mean_over_sequences, run_eval,
                           scored_frames)
