"""What is read from responses and fits: crash metrics, summaries, the energy audit, the
ISO/TS 18571 rating, predictions with their intervals and the intervals' calibration."""
