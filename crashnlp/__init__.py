"""crashnlp: elastic-pendulum frontal-crash models, identified and designed by NLP."""
__version__ = "0.1.0"
