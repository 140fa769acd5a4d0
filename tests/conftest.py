"""Settings for the whole test run.

The tests' NLPs are not compiled to C: nearly every test builds an NLP of a shape of its
own, and compiling it costs more than solving it (the model's small functions still are).
tests/test_oracle.py compiles its own, on purpose.
"""

import os

os.environ.setdefault("CRASHNLP_COMPILE", "model")
