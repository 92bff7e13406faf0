"""Mid-Air: on-disk encodings, split CSVs and the sequence dataset."""
