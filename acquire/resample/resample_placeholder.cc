// Placeholder until the resampler lands.
