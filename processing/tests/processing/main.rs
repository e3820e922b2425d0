//! The processing chain's integration tests, one binary (one link).

mod bracket;
mod common;
mod fitting;
mod synthetic;

mod albedo;
mod brdf;
mod budget;
mod capture;
mod color;
mod colour_change;
mod colour_difference;
mod export;
mod extract;
mod fit;
mod fit_fresnel;
mod geometry;
mod hdr;
mod hdr_debevec;
mod hdr_family;
mod metrics;
mod multi_angle;
mod reference;
mod samples;
mod study_stats;
mod study_synthetic;
mod table;
mod uncertainty;
