export { DEBUG, EXTENSION, FILTERS, HHDLightmapControls, HHDLightmapPlugin } from './HHDLightmapPlugin.js';
export { HHD_COMMON, blendGLSL } from './shaders.js';
