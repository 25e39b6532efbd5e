//! Symbolic differentiation. (Skeleton.)
