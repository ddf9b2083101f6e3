"""Data: the dataset store and splits, NeRF2 folders, the training views and samples."""
