//! Shared helpers for the behaviour tests of `cms-core`.
