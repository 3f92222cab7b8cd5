// Placeholder until the fitting engine lands.
