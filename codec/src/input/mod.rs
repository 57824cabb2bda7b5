//! DEM input readers (being written).
