"""Crash test data: readers (CSV, NHTSA EV5, NHTSA channel files, ISO-MME), CFC filtering and integration, in SI."""

from crashnlp.data.channels import Channel, DataError, TestData
from crashnlp.data.load import load_test_data

__all__ = ["Channel", "DataError", "TestData", "load_test_data"]
