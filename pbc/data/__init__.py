"""The dataset on disk (generation, storage) and the Lightning DataModule that serves it."""
