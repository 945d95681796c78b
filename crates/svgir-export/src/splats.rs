//! Splats for viewers (filled in below).
