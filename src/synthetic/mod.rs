//! Scenes generated with their truth known: `generate-city`, a district of box buildings as
//! large as asked, surveyed from the air and rendered by our own renderer, for showing training
//! past one device (`docs/partition.md`) on a scene no capture on disk matches in size.

pub mod city;
pub mod write;

pub use city::{generate, City, CitySpec};
pub use write::{write_city, CityReport};
