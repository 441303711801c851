pub mod inner_estimate;
