"""A problem made ready to compute: its tests' data loaded (testcase), what it leaves out
completed from them (completion, segmentation), its checks, and the Case that builds the model."""
