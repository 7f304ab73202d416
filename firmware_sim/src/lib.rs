//! Simulated motor controllers.
