"""The paper's data set: phantoms, per-view motion, simulation of one sample, whole data sets."""
