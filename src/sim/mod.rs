//! Synthetic focus stacks with ground truth.
