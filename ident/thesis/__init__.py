"""The PA10 thesis study (002): campaign fits and Tables 5-1..B-2."""
