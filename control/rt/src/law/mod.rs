pub mod admittance;
