//! Neville quincunx lifting (being written).
