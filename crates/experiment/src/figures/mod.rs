//! Figures as PNG and SVG: the drawing mechanism ([`plot`]), charts ([`charts`]) and image grids
//! ([`images`]).

pub mod charts;
pub mod images;
pub mod plot;
