//! End-to-end tests for gazelight live in `tests/tests/`; this library is empty.
